"""The KKT residual, the one judge of every solver, on points it must flag.

Each component has an independent oracle: the relative constraint violation of ``1.1 f``
is 0.1 by construction, the negativity of a point with one entry set to -c is
``c / max f``, and the momentum change is a sum written out here.
"""

import numpy as np
import pytest

from jko_cvx import CollisionProblem, Grid, PowerKernel, solve_collision

G = Grid.uniform(-2.0, 2.0, 41)
F_STAR = np.exp(-2 * G.points**2)


def _solved(conserve_momentum=False):
    prob = CollisionProblem(G, PowerKernel(1.5), F_STAR, 0.02, beta=10.0, conserve_momentum=conserve_momentum)
    res = solve_collision(prob, method="newton", tol=1e-12)
    assert res.success and res.kkt_residual <= 1e-12
    return prob, res


def test_the_certified_point_passes_every_component():
    prob, res = _solved()
    kkt = prob.kkt_residual(res.f, res.m)
    assert max(kkt.stationarity, kkt.feasibility, kkt.positivity) == kkt.total <= 1e-12
    assert kkt.positivity == 0.0


def test_an_infeasible_point_is_flagged_by_its_constraint_violation():
    """``(1.1 f, m)`` at a solution: ``h (1.1 f - f*) + D m = 0.1 h f``, i.e. 10 % of the mass."""
    prob, res = _solved()
    kkt = prob.kkt_residual(1.1 * res.f, res.m)
    assert kkt.feasibility == pytest.approx(0.1, rel=1e-10)
    assert kkt.total >= kkt.feasibility


def test_a_negative_point_is_flagged_by_its_negativity():
    """A feasible point (its own flux) with one tail value set to -0.05: negativity 0.05 / max f."""
    prob, res = _solved()
    f = res.f.copy()
    f[3] = -0.05
    f[G.n // 2] += (res.f[3] + 0.05) * G.h[3] / G.h[G.n // 2]  # keep the mass
    m = prob.flux_from_density(f)
    kkt = prob.kkt_residual(f, m)
    assert kkt.feasibility <= 1e-14
    assert kkt.positivity == pytest.approx(0.05 / f.max(), rel=1e-12)
    assert kkt.total >= kkt.positivity > 1e-2


def test_the_momentum_constraint_counts_in_the_feasibility():
    """With conserve_momentum a feasible point that moves mass one cell right is flagged by
    ``|sum_j v_j h_j (f_j - f*_j)| / sum_j |v_j| h_j f*_j``."""
    prob, res = _solved(conserve_momentum=True)
    shifted = np.r_[res.f[0], res.f[:-1]]
    shifted *= prob.mass / (shifted @ G.h)
    m = prob.flux_from_density(shifted)
    v, h = G.points, G.h
    expected = abs((shifted - F_STAR) @ (v * h)) / (F_STAR @ (np.abs(v) * h))
    assert expected > 1e-3
    kkt = prob.kkt_residual(shifted, m)
    assert kkt.feasibility == pytest.approx(expected, rel=1e-10)
    plain = CollisionProblem(G, PowerKernel(1.5), F_STAR, 0.02, beta=10.0).kkt_residual(shifted, m)
    assert plain.feasibility <= 1e-14  # the same point satisfies the paper's constraint


def test_a_batched_residual_flags_only_the_bad_slice():
    prob, res = _solved()
    batch = prob.with_f_star(np.stack([F_STAR, F_STAR, F_STAR]))
    f = np.stack([res.f, 1.1 * res.f, res.f])
    f[2, 3] = -0.05
    kkt = batch.kkt_residual(f, np.stack([res.m, res.m, res.m]))
    assert kkt.total[0] <= 1e-12
    assert kkt.feasibility[1] == pytest.approx(0.1, rel=1e-10)
    assert kkt.positivity[2] == pytest.approx(0.05 / f[2].max(), rel=1e-12) and kkt.total[2] >= kkt.positivity[2]
    assert kkt.positivity[0] == kkt.positivity[1] == 0.0
