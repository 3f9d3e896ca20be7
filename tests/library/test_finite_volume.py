"""The finite-volume peer (jko_cvx.finite_volume) against the exact solutions and its invariants."""

import numpy as np
import pytest

from jko_cvx.exact import GaussianMixture, exact_gamma1, exact_gamma2
from jko_cvx.finite_volume import Cells, _Velocity, evolve_finite_volume
from jko_cvx.kernels import PowerKernel

F0 = GaussianMixture([1.0], [2.0], [0.1], -3.0, 3.0)


def _exact_averages(cells: Cells, gamma: float, t: float) -> np.ndarray:
    """Cell averages of the exact point values by 6-point Gauss-Legendre per cell (independent of the scheme)."""
    x, w = np.polynomial.legendre.leggauss(6)
    e = cells.edges
    pts = (e[:-1, None] + e[1:, None]) / 2 + x[None, :] * cells.dv / 2
    exact = exact_gamma1 if gamma == 1.0 else exact_gamma2
    return exact(F0, t, pts.ravel()).reshape(pts.shape) @ w / 2


@pytest.mark.parametrize(("gamma", "t_end"), [(1.0, 0.25), (2.0, 0.5)])
def test_second_order_against_the_exact_solution(gamma, t_end):
    ns = (100, 200, 400, 800)
    errors = []
    for n in ns:
        cells = Cells(-3.0, 3.0, n)
        run = evolve_finite_volume(cells, PowerKernel(gamma), cells.averages(F0.cdf), t_end)
        errors.append(np.sum(np.abs(run.f - _exact_averages(cells, gamma, t_end))) * cells.dv / F0.mass)
        assert run.times[-1] == t_end
        assert run.f.min() >= 0.0
        assert abs(cells.mass(run.f) - F0.mass) <= 1e-13 * F0.mass
    order = -np.polyfit(np.log(ns), np.log(errors), 1)[0]
    assert order >= 1.75, (order, errors)
    # the last refinement is close to the asymptotic order 2
    assert np.log2(errors[-2] / errors[-1]) >= 1.85, errors


def test_positivity_and_mass_with_vacuum_and_blow_up_close():
    """A compactly supported datum (vacuum cells, jumps) run to 0.95 T for gamma = 1: stays non-negative."""
    cells = Cells(-2.0, 2.0, 200)
    c = cells.centres
    f0 = np.where(np.abs(c - 0.3) < 0.5, 1.0, 0.0) + np.where(np.abs(c + 0.8) < 0.2, 0.5, 0.0)
    mass = cells.mass(f0)
    run = evolve_finite_volume(cells, PowerKernel(1.0), f0, 0.95 * 0.5)
    assert run.f.min() >= 0.0
    assert abs(cells.mass(run.f) - mass) <= 1e-13 * mass
    assert run.f.max() > 5.0  # it concentrates


@pytest.mark.parametrize("gamma", [1.0, 2.0])
def test_dense_velocity_matches_the_closed_forms(gamma):
    """The dense exact-quadrature path at gamma +- 1e-9 against the O(N) formulas at gamma = 1, 2."""
    cells = Cells(-2.0, 1.5, 57)
    f = np.random.default_rng(0).random(cells.n)
    fast = _Velocity(cells, PowerKernel(gamma), 0.7)(f)
    dense = _Velocity(cells, PowerKernel(gamma + 1e-9), 0.7)
    assert dense.matrix is not None
    np.testing.assert_allclose(dense(f), fast, rtol=1e-7, atol=1e-7)


def test_bad_input_is_rejected_by_name():
    cells = Cells(-1.0, 1.0, 10)
    k = PowerKernel(1.5)
    with pytest.raises(ValueError, match="cfl"):
        evolve_finite_volume(cells, k, np.ones(10), 0.1, cfl=0.6)
    with pytest.raises(ValueError, match="t_end"):
        evolve_finite_volume(cells, k, np.ones(10), -1.0)
    with pytest.raises(ValueError, match="f0"):
        evolve_finite_volume(cells, k, np.ones(9), 0.1)
    with pytest.raises(ValueError, match="f0"):
        evolve_finite_volume(cells, k, -np.ones(10), 0.1)
    with pytest.raises(ValueError, match="theta"):
        evolve_finite_volume(cells, k, np.ones(10), 0.1, theta=3.0)
    with pytest.raises(ValueError, match="n must"):
        Cells(-1.0, 1.0, 2)


def test_study_errors_w2_of_a_translate_is_the_shift():
    """The study W2 (quantile functions) against the exact quantile: 0 for the exact solution, |shift| for a shift."""
    from jko_cvx.studies.solvers.peer import CASES, errors

    case = CASES["smooth_g2"]
    cells = Cells(case.lo, case.hi, 3000)
    x, w = np.polynomial.legendre.leggauss(6)
    e = cells.edges
    pts = (e[:-1, None] + e[1:, None]) / 2 + x[None, :] * cells.dv / 2

    def averages(shift):
        return case.exact(pts.ravel() - shift).reshape(pts.shape) @ w / 2

    same = errors("smooth_g2", "cells", e, averages(0.0))
    assert same["l1"] < 1e-9 and same["w2"] < 1e-4
    moved = errors("smooth_g2", "cells", e, averages(0.02))
    assert moved["w2"] == pytest.approx(0.02, rel=0.02)
    grid_pts = np.linspace(case.lo, case.hi, 1201)
    on_grid = errors("smooth_g2", "grid", grid_pts, case.exact(grid_pts))
    assert on_grid["l1"] == 0.0 and on_grid["w2"] < 1e-3


@pytest.mark.slow
def test_work_precision_peer_quick(tmp_path):
    from jko_cvx.studies.solvers.peer import work_precision_peer

    df = work_precision_peer(tmp_path, quick=True)
    for suffix in (".csv", ".md", ".png", "_time_order.csv", "_time_order.png"):
        assert (tmp_path / f"work_precision_peer{suffix}").exists()
    assert {"peer", "newton", "newton:order2", "newton+refine"} <= set(df.method)
    smooth = df[(df.case == "smooth_g1") & np.isfinite(df.l1)]
    # the peer beats first-order Newton on smooth data at its finest point
    assert smooth[smooth.method == "peer"].l1.min() < smooth[smooth.method == "newton"].l1.min()
