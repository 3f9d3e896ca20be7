"""Repeated collision steps converge at first order in dt to exact solutions.

gamma = 2: the homogeneous equation is linear (contraction about the mean velocity).
gamma = 1: Burgers characteristics before the blow-up time T = 1/(2 max f0) = 0.5.
The Fisher weight beta = 30 keeps the regularisation bias (O(dt / beta^2) per unit time)
well below the time-discretisation error; N = 241 keeps the spatial error below it too.
"""

import numpy as np
import pytest

from jko_cvx import Grid, PowerKernel
from jko_cvx.evolve import evolve_fixed_grid
from jko_cvx.exact import GaussianMixture, blowup_time_gamma1, exact_gamma1, exact_gamma2

L = 3.0
GRID = Grid.uniform(-L, L, 241)
F0 = GaussianMixture([1.0], [2.0], [0.1], -L, L)  # off-centre, so the mean velocity is not 0
DTS = np.array([0.04, 0.02, 0.01, 0.005])


def _l1_error(f, exact):
    return float(np.sum(GRID.h * np.abs(f - exact)) / np.sum(GRID.h * exact))


def _errors(gamma, t_end, exact):
    errs = []
    for dt in DTS:
        run = evolve_fixed_grid(
            GRID,
            PowerKernel(gamma),
            F0.pdf(GRID.points),
            dt,
            t_end,
            beta=30.0,
            method="conic",
            stop_on_failure=False,
        )
        assert run.times[-1] == pytest.approx(t_end)
        for res in run.results:
            # every step certified by the KKT residual (the independent judge), mass exact
            assert res.kkt_residual <= 1e-6, res.message
            assert res.mass_error <= 1e-12
        errs.append(_l1_error(run.f[-1], exact(F0, t_end, GRID.points)))
    return np.array(errs)


def test_gamma2_linear_scaling_first_order():
    errs = _errors(2.0, 0.5, exact_gamma2)
    slope = np.polyfit(np.log(DTS), np.log(errs), 1)[0]
    assert 0.8 <= slope <= 1.3, (slope, errs)
    assert errs[-1] < 1e-2
    assert np.all(np.diff(errs) < 0)


def test_gamma1_burgers_first_order_before_blowup():
    assert blowup_time_gamma1(F0) == pytest.approx(0.5)
    errs = _errors(1.0, 0.25, exact_gamma1)
    slope = np.polyfit(np.log(DTS), np.log(errs), 1)[0]
    assert 0.8 <= slope <= 1.3, (slope, errs)
    assert errs[-1] < 1e-2
    assert np.all(np.diff(errs) < 0)


def test_exact_solutions_conserve_mass():
    """Sanity of the reference formulas themselves (independent of the scheme)."""
    fine = np.linspace(-L, L, 200001)
    w = np.gradient(fine)
    for t in (0.1, 0.3, 0.45):
        assert np.sum(w * exact_gamma1(F0, t, fine)) == pytest.approx(F0.mass, rel=1e-6)
        assert np.sum(w * exact_gamma2(F0, t, fine)) == pytest.approx(F0.mass, rel=1e-6)
