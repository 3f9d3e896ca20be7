"""The right panel of ``fig:explicit2`` (``explicit2_sketch``) against the exact formulas and an ODE solve."""

import numpy as np
import pandas as pd
from scipy.integrate import solve_ivp

from jko_cvx.studies.reproduce.explicit import RHO0, T, closed_form
from jko_cvx.studies.reproduce.explicit_sketch import reproduce_explicit2_sketch


def _characteristic_ode(x: float, v: float, lam: float, t: np.ndarray) -> np.ndarray:
    """X' = V, V' = lambda/2 rho(t) (b(t) X - V), integrated numerically (not the closed form)."""

    def rhs(s, y):
        c = closed_form(np.array(s), lam)
        return [y[1], lam / 2 * c["rho"] * (c["b"] * y[0] - y[1])]

    return solve_ivp(rhs, (0.0, t[-1]), [x, v], method="DOP853", t_eval=t, rtol=1e-12, atol=1e-14).y


def test_the_sketch_curves_are_the_exact_support_and_characteristic(tmp_path):
    nums = reproduce_explicit2_sketch(tmp_path).iloc[0]
    curves = pd.read_csv(tmp_path / "explicit2_sketch_curves.csv")
    assert (tmp_path / "fig_explicit2_right.png").stat().st_size > 0
    lam = nums["lambda"]
    path = curves[curves.curve == "characteristic"]
    X, V = _characteristic_ode(nums.x1, nums.v1, lam, path.s.to_numpy())
    assert np.abs(path.x - X).max() < 1e-10 and np.abs(path.v - V).max() < 1e-8
    c = closed_form(path.s.to_numpy(), lam)
    alpha = c["m"] / c["rho"] * (path.v - c["b"] * path.x)  # sqrt(a) (V - b X), conserved along it
    assert np.allclose(alpha, nums.alpha1, rtol=1e-10) and nums.alpha1 > nums.alpha_s  # outside supp f
    for name in ("band at T_* (lower)", "band at T_* (upper)", "band at t = 0 (lower)", "band at t = 0 (upper)"):
        g = curves[curves.curve == name]
        c = closed_form(g.s.to_numpy(), lam)
        edge = c["m"] / c["rho"] * (g.v - c["b"] * g.x)
        assert np.allclose(edge, nums.alpha_s if "upper" in name else -nums.alpha_s, rtol=1e-12)


def test_the_sketch_points_make_the_papers_argument(tmp_path):
    n = reproduce_explicit2_sketch(tmp_path).iloc[0]
    kappa = n["lambda"] / 2 * RHO0 * T
    assert kappa > 1 and -n.x1 / T < n.v1 < -n.x1 / T * kappa  # thres and xvcond
    assert n["max X1 over [0, T)"] < 0  # the characteristic never reaches x = 0
    assert n["max abs(X1 numerical - closed form)"] < 1e-10
    # on the line x = X1(T_*): the band around b X1, then V1 (outside), then v_*: two components
    assert n["band from"] < n["b X1(T_*)"] < n["band to"] < n["V1(T_*)"] < n["v_*"]
    assert n["components on x = X1(T_*)"] == 2
