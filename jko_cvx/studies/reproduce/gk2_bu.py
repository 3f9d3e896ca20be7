"""``fig:gk2_bu``: f at the numerical blow-up time for lambda = 310, 300, 290, 280, whole and zoomed.

The caption: gamma = 2, ``eqn:ic_g2``, N_x = 121, N_v = 201, delta0 = delta = 0.5 in x and v;
"from top to bottom the plots show numerical solutions and their zoom-in at the numerical
blowup time".  The runs are those of ``tab:g2bu``
(:func:`~jko_cvx.studies.reproduce.g2bu.g2bu_run` on the scene
:func:`~jko_cvx.studies.reproduce.g2bu.g2bu_scene`, the same sweep points and cache directory, so
after ``tab_g2bu`` in the same code state nothing runs again): the figure is drawn from the
run's last snapshot, taken at T_b.  The zoom-in is the box of {f >= 0.1 max f}
(:func:`~jko_cvx.studies.reproduce.phase_views.zoom_window`).  Beside each row: the connected
components of {f(T_b, x, .) > 0.1} on the x-slices, the level-set check of ``thm_condbu``
that the paper reads off these panels.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.studies.reproduce.g2bu import LEVEL, g2bu_run, g2bu_scene, level_set_components
from jko_cvx.studies.reproduce.paper import TAB_G2BU
from jko_cvx.studies.reproduce.phase_views import snapshot_numbers, surface_view, zoom_window
from jko_cvx.studies.solvers.figures import pyplot
from jko_cvx.studies.sweep import run_sweep

__all__ = ["LAMBDAS", "initial_mass", "reproduce_gk2_bu"]

LAMBDAS = (310.0, 300.0, 290.0, 280.0)
"""The rows of ``fig:gk2_bu``, top to bottom."""


def initial_mass(lam: float, n_x: int, n_v: int) -> float:
    """The mass of ``eqn:ic_g2`` on the scene's initial uniform grids (the quadrature of the diagnostics)."""
    scene = g2bu_scene(lam, n_x, n_v)
    xgrid, vgrid = scene.xgrid(), scene.vgrid()
    return float(np.sum(np.outer(xgrid.h, vgrid.h) * scene.initial_density(xgrid, vgrid)))


def reproduce_gk2_bu(out: Path, quick: bool = False, **sweep_opts: Any) -> pd.DataFrame:
    """The four lambdas at 121 x 201 (``quick``: 310 and 280 at 31 x 51); ``gk2_bu.{csv,md}``, ``fig_gk2_bu.png``.

    One row per lambda: T_b, the snapshot's time, max f and where, the mass against the
    initial mass, min dx, min dv, the zoom window and the most level-set components.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    lams, n_x, n_v = ((310.0, 280.0), 31, 51) if quick else (LAMBDAS, 121, 201)
    points = [{"lam": lam, "n_x": n_x, "n_v": n_v} for lam in lams]
    df = run_sweep(g2bu_run, points, out / "cache" / "tab_g2bu", desc="gk2_bu", **sweep_opts)
    period = g2bu_scene(lams[0], n_x, n_v).xgrid().period
    rows = []
    for _, r in df.iterrows():
        nums = snapshot_numbers(r.final, period)
        mass0 = initial_mass(r.lam, n_x, n_v)
        rows.append(
            {
                "lambda": r.lam,
                "n_x": n_x,
                "n_v": n_v,
                "T_b": r.T_b,
                "paper T_b": TAB_G2BU[int(r.lam)],
                "reason": r.reason,
                **nums,
                "mass rel. diff": abs(nums["mass"] / mass0 - 1),
                f"max components of {{f > {LEVEL}}}": int(level_set_components(np.asarray(r.final["f"])).max()),
            }
        )
    table = pd.DataFrame(rows)
    table.to_csv(out / "gk2_bu.csv", index=False)
    record_csv(out / "gk2_bu.csv")
    write_markdown(out / "gk2_bu.md",
        f"# fig:gk2_bu: f at the numerical blow-up time, gamma = 2, eqn:ic_g2, N_x = {n_x}, N_v = {n_v}\n\n"
        "The tab_g2bu runs (g2bu_run); each row is the run's last snapshot (t = T_b).  Zoom window: the box of "
        "grid points holding {f >= 0.1 max f}, widened by 3 points.  mass rel. diff: against eqn:ic_g2 on the "
        f"initial grids.  Components: the most connected components of {{f(T_b, x, .) > {LEVEL}}} on any "
        "x-slice (thm_condbu's check asks for 1).\n\n" + table.to_markdown(index=False, floatfmt=".5g") + "\n"
    )
    _figure(df, out / "fig_gk2_bu.png")
    return table


def _figure(df: pd.DataFrame, path: Path) -> None:
    """Rows top to bottom as the caption: lambda = 310, 300, 290, 280; left whole, right zoomed."""
    plt = pyplot()
    fig = plt.figure(figsize=(10, 4.2 * len(df)))
    for k, (_, r) in enumerate(df.iterrows()):
        snap = r.final
        head = f"lambda = {r.lam:g}: f(T_b = {snap['t']:.5f}, x, v)"
        surface_view(fig.add_subplot(len(df), 2, 2 * k + 1, projection="3d"), snap, head)
        window = zoom_window(np.asarray(snap["f"]))
        zoomed = fig.add_subplot(len(df), 2, 2 * k + 2, projection="3d")
        surface_view(zoomed, snap, "zoom-in: the box of {f >= 0.1 max f}", window)
    fig.suptitle(f"fig:gk2_bu: N_x = {r.n_x}, N_v = {r.n_v}, at the numerical blow-up time")
    fig.tight_layout(rect=(0, 0, 1, 0.98))
    fig.savefig(path, dpi=100)
    plt.close(fig)
