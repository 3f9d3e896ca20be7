"""The gamma = 3 panels of ``fig:gk3_ih_2_C2_2``, ``fig:gk3_ih_2_C2``, ``fig:gk3_ih_2_C5_2``, ``fig:gk3_ih_2_C5``.

``sec:sp_inhom_gamma_3`` for lambda = 4 (``C2``) and lambda = 10 (``C5``), N_x = N_v = 121, to
t = 4: the runs of the ``inhom_gamma3`` entry
(:func:`~jko_cvx.studies.reproduce.inhomogeneous.inhomogeneous_gamma3`, the same sweep points and
cache directory, so after ``inhom_gamma3`` in the same code state nothing runs again).

* ``fig:gk3_ih_2_C2_2`` / ``fig:gk3_ih_2_C5_2``: surface views of f(t, x, v) at the paper's
  times (lambda = 4: t = 0.4, 0.6, 0.8, 1, 1.6, 2; lambda = 10: t = 0.2, 0.6, 0.8, 1, 1.2, 2).
* ``fig:gk3_ih_2_C2`` / ``fig:gk3_ih_2_C5``: f(4, x, v) as a surface, its zoom-in
  (:func:`~jko_cvx.studies.reproduce.phase_views.zoom_window`: the box of {f >= 0.1 max f}), the
  contour plot, and the records min dx, min dv, max f against t.

The paper's text calls the second figure "a more detailed plot at t = 3"; its captions say
t = 4, which is what we draw.  The records summary (``gk3_panels_records.csv``) holds the
numbers behind the paper's reading of the records panel: min dx and min dv fall and rise
again, max f rises and falls (no blow-up).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.studies.reproduce.inhomogeneous import PAPER_TIMES, inhomogeneous_gamma3, inhomogeneous_scene
from jko_cvx.studies.reproduce.phase_views import contour_view, snapshot_numbers, surface_view, zoom_window
from jko_cvx.studies.solvers.figures import pyplot
from jko_cvx.studies.sweep import run_sweep

__all__ = ["FIGURES", "reproduce_gk3_panels"]

FIGURES = {4.0: ("fig:gk3_ih_2_C2_2", "fig:gk3_ih_2_C2"), 10.0: ("fig:gk3_ih_2_C5_2", "fig:gk3_ih_2_C5")}
"""lambda -> (the snapshot figure, the final-time figure)."""


def reproduce_gk3_panels(out: Path, quick: bool = False, **sweep_opts: Any) -> pd.DataFrame:
    """lambda = 4 and 10 at 121 x 121 to t = 4 (``quick``: 31 x 31 to t = 2); writes ``gk3_panels.*``, 4 PNGs.

    Returns one row per panel: the lambda, the figure, t, max f and where, the mass and its
    relative difference from the initial mass, min dx, min dv and (final panels) the zoom window.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    n, t_end = (31, 2.0) if quick else (121, 4.0)
    points = [{"lam": lam, "n": n, "t_end": t_end} for lam in FIGURES]
    df = run_sweep(inhomogeneous_gamma3, points, out / "cache" / "inhom_gamma3", desc="gk3_panels", **sweep_opts)
    rows, records = [], []
    for _, r in df.iterrows():
        period = inhomogeneous_scene(r.lam, n, t_end).xgrid().period
        final = {"t": r.t[-1], "x": r.x, "v": r.v, "f": r.f}
        panels = [(FIGURES[r.lam][0], snap) for snap in r.snapshots] + [(FIGURES[r.lam][1], final)]
        for figure, snap in panels:
            nums = snapshot_numbers(snap, period)
            if figure != FIGURES[r.lam][1]:  # only the final-time figure has a zoom-in
                nums |= {k: np.nan for k in nums if k.startswith("zoom")}
            rows.append({"lambda": r.lam, "N": n, "figure": figure, **nums})
            rows[-1]["mass rel. diff"] = abs(nums["mass"] / r.mass[0] - 1)
        records.append(_records(r))
        _snapshot_figure(r, out / f"{_stem(FIGURES[r.lam][0])}.png")
        _final_figure(r, final, out / f"{_stem(FIGURES[r.lam][1])}.png")
    panels_df = pd.DataFrame(rows)
    records_df = pd.DataFrame(records)
    panels_df.to_csv(out / "gk3_panels.csv", index=False)
    record_csv(out / "gk3_panels.csv")
    records_df.to_csv(out / "gk3_panels_records.csv", index=False)
    record_csv(out / "gk3_panels_records.csv")
    write_markdown(out / "gk3_panels.md",
        f"# fig:gk3_ih_2_C2_2, fig:gk3_ih_2_C2, fig:gk3_ih_2_C5_2, fig:gk3_ih_2_C5: gamma = 3, N = {n}, "
        f"to t = {t_end:g}\n\n"
        "The inhom_gamma3 runs (eqn:f0, delta0 = 0.02, delta = 0.5, dt = 0.05).  One row per panel: the "
        "snapshot figures at the paper's times, the final-time figure at the end time (zoom window: the "
        "box of grid points holding {f >= 0.1 max f}, widened by 3 points).  mass rel. diff: against "
        "the initial mass.\n\n"
        + panels_df.to_markdown(index=False, floatfmt=".4g")
        + "\n\n## Records panel (min dx, min dv, max f against t)\n\n"
        "Paper: lambda = 4, min dx and min dv decrease and then increase, max f increases and then "
        "decreases (concentration, then separation; no blow-up); lambda = 10, min dx decreases and then "
        "increases (spreading along x).  A turn counts when the end value differs from the extreme by more "
        "than 1e-9 relative.\n\n"
        + records_df.to_markdown(index=False, floatfmt=".4g")
        + "\n"
    )
    return panels_df


def _stem(figure: str) -> str:
    return figure.replace(":", "_")


def _records(r: pd.Series) -> dict[str, Any]:
    """Where the records min dx, min dv and max f turn, their values at the end, and whether they turn back."""
    t = np.asarray(r.t)
    rec: dict[str, Any] = {"lambda": r.lam, "N": r.n, "t end": float(t[-1]), "verdict": r.verdict}
    turns = (("min_dx", np.argmin, "falls then rises"), ("min_dv", np.argmin, "falls then rises"))
    for name, turn, words in (*turns, ("max_f", np.argmax, "rises then falls")):
        series = np.asarray(r[name])
        k = int(turn(series))
        rec |= {f"{name} at t = 0": series[0], f"{name} extreme": series[k], f"t of {name} extreme": float(t[k])}
        rec[f"{name} at end"] = series[-1]
        rec[f"{name} {words}"] = bool(k > 0 and abs(series[-1] - series[k]) > 1e-9 * abs(series[k]))
    return rec


def _snapshot_figure(r: pd.Series, path: Path) -> None:
    plt = pyplot()
    snaps = r.snapshots
    fig = plt.figure(figsize=(12, 7.2))
    for k, snap in enumerate(snaps):
        ax = fig.add_subplot(2, 3, k + 1, projection="3d")
        surface_view(ax, snap, f"t = {snap['t']:.3g}, max f = {np.max(snap['f']):.3g}")
    times = ", ".join(f"{tk:g}" for tk in PAPER_TIMES[r.lam])
    fig.suptitle(f"{FIGURES[r.lam][0]}: f(t, x, v), lambda = {r.lam:g}, N = {r.n} (paper's times {times})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _final_figure(r: pd.Series, final: dict[str, Any], path: Path) -> None:
    plt = pyplot()
    fig = plt.figure(figsize=(11, 9))
    t = final["t"]
    surface_view(fig.add_subplot(2, 2, 1, projection="3d"), final, f"f(t = {t:.3g}, x, v)")
    window = zoom_window(np.asarray(final["f"]))
    surface_view(fig.add_subplot(2, 2, 2, projection="3d"), final, "zoom-in: the box of {f >= 0.1 max f}", window)
    contour_view(fig.add_subplot(2, 2, 3), final, f"contour plot of f(t = {t:.3g}, x, v)")
    ax = fig.add_subplot(2, 2, 4)
    for name in ("min_dx", "min_dv", "max_f"):
        ax.semilogy(r.t, r[name], label=name.replace("_", " "))
    ax.set_xlabel("t")
    ax.set_title("records at each time step", fontsize=8)
    ax.legend(fontsize=7)
    fig.suptitle(f"{FIGURES[r.lam][1]}: lambda = {r.lam:g}, N = {r.n}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
