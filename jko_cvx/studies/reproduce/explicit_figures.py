"""``fig:explicit1``-``fig:explicit3``: the infinite-mass solution and its characteristics.

* ``fig:explicit1``: the ansatz :math:`f = m\\,\\phi(a (v - b x)^2)`,
  :math:`\\phi(s) = e^{-s}/\\sqrt{2\\pi}`, with the closed forms ``rhot``, ``mt``
  (:func:`~jko_cvx.studies.reproduce.explicit.closed_form`), :math:`a = (m/\\rho)^2`, at t = 0, T/2,
  0.9 T for a super-critical lambda = 400 (``thres``: :math:`\\lambda\\rho_0 T = 2.58 > 2`).
* ``fig:explicit2`` (left panel): a characteristic of ``eq``,
  :math:`\\dot X = V, \\dot V = \\tfrac\\lambda2 \\rho(t)(b(t) X - V)`, from x < 0 with v in
  the set ``xvcond`` (:math:`-x/T < v \\le -\\tfrac{x}{T}\\tfrac\\lambda2\\rho_0 T`), which
  stays in x < 0 up to T, beside one from above that set, which crosses 0.  The ODE is
  integrated numerically (DOP853) and compared with the paper's closed form
  :math:`X/(T-t) = x/T + \\frac{\\alpha\\rho_0}{m_0}\\frac{(T/(T-t))^{1-\\kappa} - 1}{1-\\kappa}`,
  :math:`\\kappa = \\tfrac\\lambda2\\rho_0 T`.  (The right panel of ``fig:explicit2``, a
  sketch of a broken ``condft``, is the ``explicit2_sketch`` entry,
  :mod:`~jko_cvx.studies.reproduce.explicit_sketch`; the level-set check of ``tab_g2bu`` is its numerical form.)
* ``fig:explicit3``: a characteristic of ``eqgamma``, :math:`\\dot X = -X/(T-t) + \\alpha C`,
  from :math:`X_0 < 0` with :math:`\\alpha > 0`: it reaches 0 before T, at
  :math:`t_0 = T(1 - e^{-|X_0|/(\\alpha C T)})` by the closed form
  :math:`X = \\frac{T-t}{T}(X_0 + \\alpha C T \\ln\\frac{T}{T-t})`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from scipy.integrate import solve_ivp

from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.studies.reproduce.explicit import M0, RHO0, T, closed_form
from jko_cvx.studies.solvers.figures import pyplot

__all__ = ["characteristic_eq", "characteristic_eqgamma", "reproduce_explicit_figures"]

LAMBDA = 400.0
_EDGE = 1 - 1e-6  # integrate to (1 - 1e-6) T


def characteristic_eq(x: float, v: float, lam: float, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(numerical X, closed-form X) of the characteristic of ``eq`` from (x, v) at times ``t < T``."""

    def rhs(s: float, y: np.ndarray) -> np.ndarray:
        c = closed_form(np.array(s), lam)
        return np.array([y[1], lam / 2 * c["rho"] * (c["b"] * y[0] - y[1])])

    sol = solve_ivp(rhs, (0.0, float(t[-1])), [x, v], method="DOP853", t_eval=t, rtol=1e-11, atol=1e-13)
    if not sol.success:
        raise RuntimeError(f"characteristic integration failed: {sol.message}")
    kappa = lam / 2 * RHO0 * T
    alpha = M0 / RHO0 * (v + x / T)
    exact = (T - t) * (x / T + alpha * RHO0 / M0 / (1 - kappa) * ((T / (T - t)) ** (1 - kappa) - 1))
    return sol.y[0], exact


def characteristic_eqgamma(x0: float, alpha_c: float, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(numerical X, closed-form X) of :math:`\\dot X = -X/(T-t) + \\alpha C` from ``x0``."""
    sol = solve_ivp(
        lambda s, y: -y / (T - s) + alpha_c, (0.0, float(t[-1])), [x0], method="DOP853", t_eval=t, rtol=1e-11
    )
    if not sol.success:
        raise RuntimeError(f"characteristic integration failed: {sol.message}")
    return sol.y[0], (T - t) / T * (x0 + alpha_c * T * np.log(T / (T - t)))


def reproduce_explicit_figures(out: Path, quick: bool = False, **_sweep_opts: Any) -> pd.DataFrame:
    """Write ``explicit_figures.{csv,md,png}`` (``quick`` is the same: a second of work)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t = T * (1 - np.geomspace(1, 1 - _EDGE, 400))
    t[0] = 0.0
    kappa = LAMBDA / 2 * RHO0 * T
    x = -0.2
    v_in = -x / T * (1 + kappa) / 2  # the middle of xvcond
    v_out = -x / T * kappa * 1.2  # above it
    rows, trajectories = [], {}
    for label, v in (("explicit2: v in xvcond", v_in), ("explicit2: v above xvcond", v_out)):
        num, exact = characteristic_eq(x, v, LAMBDA, t)
        trajectories[label] = (num, exact)
        rows.append(
            {
                "figure": label,
                "x0": x,
                "v0 or alpha C": v,
                "max X over (0, T)": float(num.max()),
                "stays in x < 0": bool(num.max() < 0),
                "max abs(X numerical - closed form)": float(np.abs(num - exact).max()),
            }
        )
    x0, alpha_c = -1.0, 20.0
    num, exact = characteristic_eqgamma(x0, alpha_c, t)
    trajectories["explicit3"] = (num, exact)
    k = int(np.argmax(num >= 0))  # first point at or past x = 0 (X rises through 0, then returns to 0 at T)
    crossing = float(t[k - 1] - num[k - 1] * (t[k] - t[k - 1]) / (num[k] - num[k - 1]))
    rows.append(
        {
            "figure": "explicit3",
            "x0": x0,
            "v0 or alpha C": alpha_c,
            "max X over (0, T)": float(num.max()),
            "stays in x < 0": bool(num.max() < 0),
            "max abs(X numerical - closed form)": float(np.abs(num - exact).max()),
            "crossing time (numerical)": crossing,
            "crossing time (closed form)": T * (1 - np.exp(-abs(x0) / (alpha_c * T))),
        }
    )
    df = pd.DataFrame(rows)
    df.to_csv(out / "explicit_figures.csv", index=False)
    record_csv(out / "explicit_figures.csv")
    lines = [
        "# fig:explicit1-3: the infinite-mass solution (lambda = 400) and its characteristics",
        "",
        f"kappa = lambda rho0 T / 2 = {kappa:.4g}; xvcond at x = {x}: {-x / T:.4g} < v <= {-x / T * kappa:.4g}.",
        "",
        df.to_markdown(index=False, floatfmt=".4g"),
        "",
    ]
    write_markdown(out / "explicit_figures.md", "\n".join(lines) + "\n")
    _figure(t, trajectories, out / "explicit_figures.png")
    return df


def _figure(t: np.ndarray, trajectories: dict, path: Path) -> None:
    plt = pyplot()
    fig, axes = plt.subplots(1, 5, figsize=(21, 3.8))
    xs, vs = np.linspace(-0.5, 0.5, 201), np.linspace(-8, 8, 241)
    X, V = np.meshgrid(xs, vs, indexing="ij")
    for ax, tk in zip(axes[:3], (0.0, 0.5 * T, 0.9 * T), strict=True):
        c = closed_form(np.array(tk), LAMBDA)
        a = (c["m"] / c["rho"]) ** 2
        f = c["m"] * np.exp(-a * (V - c["b"] * X) ** 2) / np.sqrt(2 * np.pi)
        ax.contourf(X, V, f, levels=20)
        ax.set_title(f"fig:explicit1: f(t = {tk / T:.1f} T, x, v), lambda = {LAMBDA:g}", fontsize=8)
        ax.set_xlabel("x")
        ax.set_ylabel("v")
    for label, (num, exact) in trajectories.items():
        ax = axes[3] if label.startswith("explicit2") else axes[4]
        ax.plot(t / T, num, label=f"{label} (ODE)")
        ax.plot(t / T, exact, "k:", lw=1)
    for ax, title in zip(axes[3:], ("fig:explicit2 (left): X(t) of eq", "fig:explicit3: X(t) of eqgamma"), strict=True):
        ax.axhline(0, color="k", lw=0.6)
        ax.set_xlabel("t / T")
        ax.set_ylabel("X")
        ax.set_title(title + "; dotted: closed form", fontsize=8)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
