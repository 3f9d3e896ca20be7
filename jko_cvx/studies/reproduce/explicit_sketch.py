"""The right panel of ``fig:explicit2``: "a possible scenario in which ``condft`` breaks down".

Drawn from the exact formulas of ``sec:412`` for the super-critical infinite-mass solution
(lambda = 400, ``thres``: kappa = lambda rho0 T / 2 = 1.29 > 1), with a compactly supported
profile phi (support s = a (v - b x)^2 <= alpha_s^2).  Along a characteristic of ``eq`` the
quantity :math:`\\alpha = \\sqrt{a}(V - bX) = \\frac{m_0}{\\rho_0}(v + x/T)` is conserved, so
the support of f(t) is the band

.. math:: \\operatorname{supp} f(t) = \\{|v - b(t) x| \\le \\alpha_s \\rho(t)/m(t)\\}

at every t, and the characteristic from (x_1, v_1) with v_1 in ``xvcond`` (alpha_1 > alpha_s,
so (x_1, v_1) lies outside the support) is

.. math:: \\frac{X_1}{T - t} = \\frac{x_1}{T} + \\frac{\\alpha_1\\rho_0}{m_0}
          \\frac{(T/(T-t))^{1-\\kappa} - 1}{1 - \\kappa}, \\qquad
          V_1 = b X_1 + \\alpha_1 \\rho/m .

The sketch at t = T_* = 0.6 T: the band (where, by the proof of ``thm_condbu``, f~ = f for
|x| <= |X_1(T_*)|), the path of (X_1, V_1) from t = 0, the half-line
{x = X_1(T_*), v >= V_1(T_*)} that ``condft`` keeps out of supp f~, and a hypothetical part of
supp f~ coming from x < X_1 that touches it at (X_1(T_*), v_*), v_* > V_1(T_*).  The vertical
line x = X_1(T_*) then meets supp f~ in the band's interval around b X_1 and in v_*: two
components, with V_1 between them (the paper's argument, and why ``tab_g2bu`` counts the
components of the level sets on every x-slice).  The hypothetical part is the only element
not given by a formula; everything else is checked against an independent ODE solve.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.studies.reproduce.explicit import M0, RHO0, T, closed_form
from jko_cvx.studies.reproduce.explicit_figures import LAMBDA, characteristic_eq
from jko_cvx.studies.reproduce.g2bu import level_set_components
from jko_cvx.studies.solvers.figures import pyplot

__all__ = ["band", "characteristic", "reproduce_explicit2_sketch", "sketch_numbers"]

X1, ALPHA_S, T_STAR = -0.2, 1.5, 0.6 * T
"""Start x of the characteristic, half-width of the profile's support in alpha, the time drawn."""


def _kappa(lam: float) -> float:
    return lam / 2 * RHO0 * T


def characteristic(x: float, v: float, lam: float, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The closed-form characteristic (X, V) of ``eq`` from (x, v) at times ``t < T`` (``sec:412``)."""
    t = np.asarray(t, dtype=float)
    kappa, alpha = _kappa(lam), M0 / RHO0 * (v + x / T)
    c = closed_form(t, lam)
    X = (T - t) * (x / T + alpha * RHO0 / M0 * ((T / (T - t)) ** (1 - kappa) - 1) / (1 - kappa))
    return X, c["b"] * X + alpha * c["rho"] / c["m"]


def band(x: np.ndarray, t: float, lam: float, alpha_s: float = ALPHA_S) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper edge in v of supp f(t) = {|v - b x| <= alpha_s rho/m} over ``x``."""
    c = closed_form(np.array(t), lam)
    half = alpha_s * c["rho"] / c["m"]
    return c["b"] * np.asarray(x) - half, c["b"] * np.asarray(x) + half


def sketch_numbers(lam: float = LAMBDA) -> dict[str, float]:
    """The points of the sketch: the characteristic at T_*, the band on its vertical line, v_*."""
    kappa = _kappa(lam)
    v1 = -X1 / T * (1 + kappa) / 2  # the middle of xvcond: -x/T < v < -x/T kappa
    X, V = characteristic(X1, v1, lam, np.array([T_STAR]))
    lo, hi = band(X, T_STAR, lam)
    t_path = np.linspace(0.0, T * (1 - 1e-6), 2001)
    X_num, X_closed = characteristic_eq(X1, v1, lam, t_path)
    v_star = float(V[0] + 2 * (V[0] - hi[0]))  # clear of V_1 by twice V_1's gap to the band
    return {
        "lambda": lam,
        "kappa = lambda rho0 T / 2": kappa,
        "x1": X1,
        "v1": v1,
        "alpha1": M0 / RHO0 * (v1 + X1 / T),
        "alpha_s": ALPHA_S,
        "T_*": T_STAR,
        "X1(T_*)": float(X[0]),
        "V1(T_*)": float(V[0]),
        "b X1(T_*)": float(closed_form(np.array(T_STAR), lam)["b"] * X[0]),
        "band from": float(lo[0]),
        "band to": float(hi[0]),
        "v_*": v_star,
        "max X1 over [0, T)": float(X_num.max()),
        "max abs(X1 numerical - closed form)": float(np.abs(X_num - X_closed).max()),
        "components on x = X1(T_*)": _components_on_line(float(lo[0]), float(hi[0]), v_star),
    }


def _components_on_line(lo: float, hi: float, v_star: float) -> int:
    """Components of {band [lo, hi]} + {v_*} on a v-grid holding all three points, counted as ``tab_g2bu``
    counts the level sets on its x-slices (:func:`~jko_cvx.studies.reproduce.g2bu.level_set_components`)."""
    v = np.union1d(np.linspace(lo - 1.0, v_star + 1.0, 2001), [lo, hi, v_star])
    support = ((v >= lo) & (v <= hi)) | (v == v_star)
    return int(level_set_components(support[None, :].astype(float), level=0.5)[0])


def reproduce_explicit2_sketch(out: Path, quick: bool = False, **_sweep_opts: Any) -> pd.DataFrame:
    """Write ``explicit2_sketch.{csv,md}``, the plotted curves ``explicit2_sketch_curves.csv`` and
    ``fig_explicit2_right.png`` (``quick`` is the same: well under a second)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    nums = sketch_numbers()
    t = np.linspace(0.0, T_STAR, 201)
    X, V = characteristic(nums["x1"], nums["v1"], LAMBDA, t)
    x = np.union1d(np.linspace(-0.25, 0.25, 501), [nums["X1(T_*)"], -nums["X1(T_*)"]])  # the band ends on x = +-X1
    lo, hi = band(x, T_STAR, LAMBDA)
    lo0, hi0 = band(x, 0.0, LAMBDA)
    curves = pd.concat(
        [
            pd.DataFrame({"curve": "characteristic", "s": t, "x": X, "v": V}),
            pd.DataFrame({"curve": "band at T_* (lower)", "s": T_STAR, "x": x, "v": lo}),
            pd.DataFrame({"curve": "band at T_* (upper)", "s": T_STAR, "x": x, "v": hi}),
            pd.DataFrame({"curve": "band at t = 0 (lower)", "s": 0.0, "x": x, "v": lo0}),
            pd.DataFrame({"curve": "band at t = 0 (upper)", "s": 0.0, "x": x, "v": hi0}),
        ],
        ignore_index=True,
    )
    curves.to_csv(out / "explicit2_sketch_curves.csv", index=False)
    record_csv(out / "explicit2_sketch_curves.csv")
    table = pd.DataFrame([nums])
    table.to_csv(out / "explicit2_sketch.csv", index=False)
    record_csv(out / "explicit2_sketch.csv")
    write_markdown(out / "explicit2_sketch.md",
        "# fig:explicit2 (right): a possible scenario in which condft breaks down\n\n"
        f"Infinite-mass solution, lambda = {LAMBDA:g}, profile supported on alpha^2 <= alpha_s^2; the characteristic "
        "from (x1, v1), v1 in xvcond, drawn at T_*.  On the line x = X1(T_*) the support holds the band "
        "[band from, band to] (around b X1) and the hypothetical point v_* > V1(T_*): two components, V1 between "
        "them.  The curves of the figure: `explicit2_sketch_curves.csv`.\n\n"
        + table.T.rename(columns={0: "value"}).to_markdown(floatfmt=".6g")
        + "\n"
    )
    _figure(nums, curves, out / "fig_explicit2_right.png")
    return table


def _figure(nums: dict[str, float], curves: pd.DataFrame, path: Path) -> None:
    """Left: the phase plane at T_*; middle: its zoom at x = X1(T_*); right: the slice on that line."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6), gridspec_kw={"width_ratios": [1.2, 1.2, 1]})
    w = (nums["band to"] - nums["band from"]) / 2
    box = (nums["X1(T_*)"] - 0.03, nums["X1(T_*)"] + 0.02, nums["band from"] - 2 * w, nums["v_*"] + 3 * w)
    for ax, lims in zip(axes[:2], ((-0.25, 0.25, -3.5, 3.5), box), strict=True):
        _phase_plane(ax, nums, curves, w, annotate=ax is axes[1])
        ax.set(xlim=lims[:2], ylim=lims[2:], xlabel="x", ylabel="v")
    axes[0].add_patch(_rectangle(box))
    head = f"fig:explicit2 (right): supp f~(T_*), T_* = {nums['T_*'] / T:.1f} T, lambda = {nums['lambda']:g}"
    axes[0].set_title(head)
    axes[1].set_title("zoom at the line x = X1(T_*)")
    axes[1].legend(fontsize=6.5, loc="lower left")
    _slice(axes[2], nums, w)
    for ax in axes:
        ax.title.set_fontsize(9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _rectangle(box: tuple[float, float, float, float]):
    from matplotlib.patches import Rectangle

    return Rectangle((box[0], box[2]), box[1] - box[0], box[3] - box[2], fill=False, color="k", lw=0.8)


def _phase_plane(ax, nums: dict[str, float], curves: pd.DataFrame, w: float, annotate: bool) -> None:
    from matplotlib.patches import Ellipse

    X1s, V1s = nums["X1(T_*)"], nums["V1(T_*)"]
    c = {name: g for name, g in curves.groupby("curve")}
    low, up = c["band at T_* (lower)"], c["band at T_* (upper)"]
    inner = np.abs(low.x.to_numpy()) <= abs(X1s)
    label = "supp f~(T_*) = supp f(T_*) on |x| <= |X1|"
    ax.fill_between(low.x[inner], low.v[inner], up.v[inner], color="C0", alpha=0.5, label=label)
    for g in (low, up):
        ax.plot(g.x, g.v, "C0--", lw=0.8)
    for name in ("band at t = 0 (lower)", "band at t = 0 (upper)"):
        ax.plot(c[name].x, c[name].v, color="0.6", ls=":", lw=0.8, label="supp f(0)" if "lower" in name else None)
    path_ = c["characteristic"]
    ax.plot(path_.x, path_.v, "k-", label="(X1(t), V1(t)), 0 <= t <= T_*, and its mirror")
    ax.plot(-path_.x, -path_.v, "k-", lw=0.6)
    top = nums["v_*"] + 10 * w
    ax.plot([X1s, X1s], [V1s, top], "r-", lw=2.5, label="x = X1(T_*), v >= V1(T_*): kept out of supp f~ by condft")
    blob = Ellipse((X1s - 0.01, nums["v_*"]), 0.02, w, color="C1", alpha=0.6, label="hypothetical part of supp f~")
    ax.add_patch(blob)
    ax.plot([X1s] * 3, [nums["b X1(T_*)"], V1s, nums["v_*"]], "ko", ms=3)
    for v, text in ((nums["b X1(T_*)"], "b X1"), (V1s, "V1"), (nums["v_*"], "v_*")) if annotate else ():
        ax.annotate(text, (X1s, v), fontsize=7, xytext=(4, -3), textcoords="offset points")


def _slice(ax, nums: dict[str, float], w: float) -> None:
    """f(T_*, X1, v) on the band (profile (1 - alpha^2/alpha_s^2)_+), the point v_*, and V1 between them."""
    v = np.linspace(nums["band from"] - w, nums["v_*"] + 3 * w, 400)
    profile = np.clip(1 - ((v - nums["b X1(T_*)"]) / w) ** 2, 0, None)
    ax.plot(v, profile, "C0", label="f(T_*, X1, v) / max f (first component)")
    ax.plot([nums["v_*"]], [0], "o", color="C1", label="v_* in supp f~ (second component)")
    ax.axvline(nums["V1(T_*)"], color="r", ls="--", lw=1, label="V1(T_*): not in supp f~")
    ax.set(xlabel="v on the line x = X1(T_*)", title="the slice x = X1(T_*): two components of supp f~")
    ax.legend(fontsize=6.5)
