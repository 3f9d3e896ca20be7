"""Threshold times extrapolated to eps_v -> 0 (and dt -> 0): an exact law, bad input, and gamma = 1
runs against the exact time T = 1/(2 max f0)."""

import numpy as np
import pytest

from jko_cvx.blowup import extrapolate_thresholds
from jko_cvx.engine.loop import simulate
from jko_cvx.exact import GaussianMixture, blowup_time_gamma1
from jko_cvx.scene import shipped_scene

EPS = np.geomspace(3e-3, 1e-4, 10)


def test_an_exact_law_gives_its_limit():
    eps = np.tile(EPS, 2)
    dt = np.repeat([0.005, 0.0025], EPS.size)
    tb = 0.5 - 2.0 * eps**0.7 + 0.3 * dt
    x = extrapolate_thresholds(eps, tb, dt)
    assert x.T == pytest.approx(0.5, abs=1e-8)
    assert (x.c, x.p, x.d) == pytest.approx((2.0, 0.7, 0.3), rel=1e-5)
    one = extrapolate_thresholds(EPS, 0.3 - 0.1 * EPS**1.5)  # one step: no dt term
    assert one.T == pytest.approx(0.3, abs=1e-8) and one.d is None


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (([1e-3, 1e-4, 1e-5], [0.4, 0.45, 0.47]), "at least 4"),
        (([1e-3, -1e-4, 1e-5, 1e-6], [0.4, 0.45, 0.47, 0.48]), "eps_v"),
        (([1e-3, 1e-4, 1e-5, 1e-6], [0.4, np.nan, 0.47, 0.48]), "never fired"),
        (([1e-3, 1e-4, 1e-5, 1e-6], [0.4, 0.45, 0.47]), "shapes"),
    ],
)
def test_bad_input_is_refused_by_name(args, match):
    with pytest.raises(ValueError, match=match):
        extrapolate_thresholds(*args)
    with pytest.raises(ValueError, match="dt"):
        extrapolate_thresholds(EPS, 0.5 - EPS**0.5, -0.01)


def _thresholds(overrides):
    """Threshold times of one run replayed from its min dv record for every eps_v of EPS."""
    sc = shipped_scene("tab_bu_g1", {**overrides, "stop.eps_v": EPS.min()})
    ic = sc.initial
    T = blowup_time_gamma1(GaussianMixture(ic.amplitudes, ic.rates, ic.centres, -sc.v.L, sc.v.L))
    d = simulate(sc).diagnostics
    t, min_dv = d.t.to_numpy(), d.min_dv.to_numpy()
    assert min_dv.min() < EPS.min()
    return T, np.array([t[np.argmax(min_dv < e)] for e in EPS])


@pytest.mark.parametrize(
    "overrides",
    [
        {"v.n": 241, "time.dt": 0.005},  # g1, T = 0.5; measured extrapolation +3.6e-3, finest threshold -0.010
        {"v.n": 481, "time.dt": 0.005},  # measured -3.9e-3 against -0.025
        {"v.n": 481, "time.dt": 0.005, "initial.amplitudes": [0.8], "initial.rates": [1.0]},  # T = 0.625: -4.9e-3
    ],
)
def test_gamma1_threshold_times_extrapolate_towards_the_exact_time(overrides):
    T, tb = _thresholds(overrides)
    x = extrapolate_thresholds(EPS, tb, overrides["time.dt"])
    assert abs(x.T - T) < 0.01
    assert abs(x.T - T) < 0.5 * abs(tb[-1] - T)  # closer than the paper's T_b at the smallest threshold
    assert 0.3 < x.p < 1.5 and x.c > 0  # the threshold fires early, the earlier the larger eps_v


def test_a_family_over_two_time_steps_extrapolates_in_both():
    T, tb1 = _thresholds({"v.n": 481, "time.dt": 0.005})
    _, tb2 = _thresholds({"v.n": 481, "time.dt": 0.0025})
    x = extrapolate_thresholds(np.tile(EPS, 2), np.concatenate([tb1, tb2]), np.repeat([0.005, 0.0025], EPS.size))
    assert x.d is not None and x.n == 2 * EPS.size
    assert abs(x.T - T) < 0.01
