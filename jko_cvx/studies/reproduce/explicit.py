"""``sec: explicit``: the infinite-mass self-similar solution for gamma = 2.

The ansatz ``f = m(t) phi(a(t) (v - b(t) x)^2)`` (eqn ``ansatz``) solves ``eq`` when
:math:`(\\rho, m, b)`, :math:`\\rho = m/\\sqrt{a}`, solves ``ode1``

.. math::

    \\rho' = -b\\rho, \\qquad m' = \\tfrac{\\lambda}{2}\\rho m, \\qquad b' = -b^2,

whose closed forms are :math:`b = -1/(T - t)`, :math:`T = -1/b_0`,
:math:`\\rho = \\rho_0 T/(T - t)` (``rhot``) and
:math:`m = m_0 (T/(T - t))^{\\lambda\\rho_0 T/2}` (``mt``).  This reproduction integrates
``ode1`` numerically (SciPy's DOP853 in the logarithmic variables, so that the solution is
resolved up to :math:`T - t = 10^{-8} T`) and tabulates its relative difference from the
closed forms as :math:`t \\to T`, together with the velocity width
:math:`1/\\sqrt{a} = \\rho/m` whose limit decides the threshold ``thres``
(:math:`\\lambda\\rho_0 T > 2`: the width closes, blow-up expected for finite mass).

Parameters are those of ``sec:sp_inhom_gamma_2``: :math:`a_0 = 120`,
:math:`\\rho_0 = \\sqrt{1/(2a_0)}`, :math:`b_0 = -10` (T = 0.1), and lambda on both sides of
the threshold :math:`2/(\\rho_0 T) = 20\\sqrt{240} \\approx 309.8`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from scipy.integrate import solve_ivp

from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.studies.solvers.figures import pyplot

__all__ = ["closed_form", "reproduce_explicit", "solve_ode1"]

A0, B0 = 120.0, -10.0
RHO0 = float(np.sqrt(1 / (2 * A0)))
M0 = RHO0 * np.sqrt(A0)  # rho = m / sqrt(a)
T = -1 / B0
LAMBDAS = (220.0, 280.0, 300.0, 309.8, 320.0, 400.0)


def closed_form(t: np.ndarray, lam: float) -> dict[str, np.ndarray]:
    """``rhot``, ``mt`` and ``b`` at times ``t < T``."""
    t = np.asarray(t, dtype=float)
    r = T / (T - t)
    return {"rho": RHO0 * r, "m": M0 * r ** (lam / 2 * RHO0 * T), "b": -1 / (T - t)}


def solve_ode1(t: np.ndarray, lam: float, rtol: float = 1e-12) -> dict[str, np.ndarray]:
    """Integrate ``ode1`` numerically (DOP853) in ``(log rho, log m, b)``; independent of the closed forms.

    Logarithms keep the relative accuracy uniform while rho and m grow like (T - t)^-1 and
    (T - t)^-(lambda rho0 T / 2).
    """

    def rhs(_s: float, y: np.ndarray) -> np.ndarray:
        log_rho, _log_m, b = y
        return np.array([-b, lam / 2 * np.exp(log_rho), -(b * b)])

    sol = solve_ivp(
        rhs,
        (0.0, float(np.max(t))),
        [np.log(RHO0), np.log(M0), B0],
        method="DOP853",
        t_eval=np.asarray(t, dtype=float),
        rtol=rtol,
        atol=1e-14,
    )
    if not sol.success:
        raise RuntimeError(f"ode1 integration failed: {sol.message}")
    return {"rho": np.exp(sol.y[0]), "m": np.exp(sol.y[1]), "b": sol.y[2]}


def reproduce_explicit(out: Path, quick: bool = False, **_sweep_opts: Any) -> pd.DataFrame:
    """Numerical ``ode1`` against ``rhot`` / ``mt``; writes ``explicit.{csv,md,png}``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    eps = np.array([1e-1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6] + ([] if quick else [1e-7, 1e-8]))
    t = T * (1 - eps)
    rows = []
    for lam in LAMBDAS[:3] if quick else LAMBDAS:
        num, exact = solve_ode1(t, lam), closed_form(t, lam)
        for i, e in enumerate(eps):
            width_num = num["rho"][i] / num["m"][i]
            rows.append(
                {
                    "lambda": lam,
                    "lambda rho0 T / 2": lam / 2 * RHO0 * T,
                    "(T-t)/T": e,
                    "rho (ode1)": num["rho"][i],
                    "rho rel. diff": abs(num["rho"][i] / exact["rho"][i] - 1),
                    "m (ode1)": num["m"][i],
                    "m rel. diff": abs(num["m"][i] / exact["m"][i] - 1),
                    "b rel. diff": abs(num["b"][i] / exact["b"][i] - 1),
                    "width 1/sqrt(a)": width_num,
                }
            )
    df = pd.DataFrame(rows)
    df.to_csv(out / "explicit.csv", index=False)
    record_csv(out / "explicit.csv")
    worst = df.groupby("(T-t)/T")[["rho rel. diff", "m rel. diff", "b rel. diff"]].max().reset_index()
    worst = worst.sort_values("(T-t)/T", ascending=False)
    trend = df[df["(T-t)/T"] == eps.min()][["lambda", "lambda rho0 T / 2", "width 1/sqrt(a)"]]
    text = (
        "# sec: explicit -- infinite-mass self-similar solution, gamma = 2\n\n"
        f"a0 = {A0:g}, rho0 = sqrt(1/(2 a0)) = {RHO0:.6g}, b0 = {B0:g} (T = {T:g}); ode1 integrated by DOP853\n"
        "(rtol 1e-12) in (log rho, log m, b), against the closed forms rhot and mt, up to (T - t)/T = "
        f"{eps.min():g}.\n\n"
        "## Relative difference, numerical ode1 against rhot / mt / b (largest over lambda)\n\n"
        "It grows like rtol x T/(T - t): the conditioning of a blow-up time, not a disagreement.\n\n"
        + worst.to_markdown(index=False, floatfmt=".2e")
        + "\n\n## Velocity width rho/m = 1/sqrt(a) at the last time (threshold lambda rho0 T / 2 = 1, thres)\n\n"
        + trend.to_markdown(index=False, floatfmt=".4g")
        + "\n\nWidth -> 0 (blow-up expected for finite mass) exactly when lambda rho0 T / 2 > 1, i.e. lambda > "
        f"{2 / (RHO0 * T):.1f}; the paper: 20 sqrt(240) ~ 310.\n\n## Every time\n\n"
        + df.to_markdown(index=False, floatfmt=".4g")
        + "\n"
    )
    write_markdown(out / "explicit.md", text)
    _figure(df, out / "explicit.png")
    return df


def _figure(df: pd.DataFrame, path: Path) -> None:
    plt = pyplot()

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for i, (lam, b) in enumerate(df.groupby("lambda")):
        eps = b["(T-t)/T"].to_numpy()
        ex = closed_form(T * (1 - eps), lam)
        axes[0].loglog(eps, b["m (ode1)"], "o", color=f"C{i}", ms=4)
        axes[0].loglog(eps, ex["m"], "-", color=f"C{i}", label=f"lambda={lam:g}")
        axes[1].loglog(eps, b["width 1/sqrt(a)"], "-o", color=f"C{i}", ms=3, label=f"lambda={lam:g}")
    axes[0].set_title("m(t): ode1 numerically (dots), closed form mt (lines)", fontsize=9)
    axes[1].set_title("velocity width 1/sqrt(a) = rho/m", fontsize=9)
    for ax in axes:
        ax.set_xlabel("(T - t) / T")
        ax.invert_xaxis()
        ax.grid(True, which="both", alpha=0.2)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
